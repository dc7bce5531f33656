"""Generates :mod:`evperc.fusion.kernel`, the straight-line per-cell code of the fused step.

The fused step (method.md §5 steps 2–8 and §6) is ~600 float operations per cell. Written as one
loop over the cells of a row whose body is straight-line code on 32 scalar masses (no inner
loops, no per-cell branches: conditions become selects), LLVM vectorises it *across cells*:
each scalar becomes one AVX register of 8–16 cells. Writing 32 masses out by hand is error
prone, so this module writes that code; the generated file is committed and
``tests/fusion/test_fused.py`` checks it is up to date. Regenerate with::

    python -m evperc.fusion.codegen

The algebra, per cell, with m the discounted state (bitmask subsets, F = 1, I = 2, U = 4,
S = 8, M = 16, O = 30, Ω = 31):

- d = m ∩ SG with SG = {F: f, O: o, Ω: u}:  d(A) = u m(A) + o (m(A) + m(A ∪ F)) for
  ∅ ≠ A ⊆ O; d({F}) = u m(F) + f Σ_{A∋F} m(A); d(A) = u m(A) for the other A ∋ F;
  d(∅) = u m(∅) + o (m(∅) + m(F)) + f Σ_{A∌F} m(A).
- m ∩ SG' with SG' = SG ⊕ GG (GG = {P: β', Ω: 1 − β'}, β' the prior mass where it is used):
  by associativity m ∩ (SG ∩ GG) = (1 − β') d + β' (d ∩ P); SG ∩ GG gives ∅ the mass
  e = β' f [F ∉ P], which Dempster's rule removes, so c = ((1 − β') d + β' (d ∩ P) − e δ_∅)
  / (1 − e). Only the building prior P = {I} has F ∉ P; there the part f (m ∩ {F}) of d goes
  wholly to ∅ and cancels e δ_∅ (as Σ m = 1), so it is left out of d ∩ P instead of being
  subtracted (no float32 cancellation when 1 − e is small). Total conflict (1 − e ≤ tol)
  keeps SG (β' = 0), as the numpy twin.
- SG'({F}) = f (1 − β'_building) / (1 − e), Bel_SG'(O) = (o + u β'_building) / (1 − e),
  so ∅_FO = m(F) Bel_SG'(O), ∅_OF = Bel_m(O) SG'({F}) (method.md §5.4).

Around the body, per block of 256 cells of a window row: trim to the active lanes, read the
planes in the union of the cells' focal-set masks (compact layout, :mod:`evperc.fusion.fused`),
zero the other planes only where an earlier block may have left values (``dirty``), run
the body, write back the planes used before or after, and the outputs. The block buffer's
planes are 272 floats apart, not 256: with 1 kB between them, one sub-block's lanes of all
45 planes fell in 4 of the L1 cache's 64 sets.

Two variants of each kernel: the general one, and a *lean* one for the options where
the I butterfly (α_I = 0), classical discounting and the ⊛ rule's normalisation are
identities — contextual discounting with α_I = 0 and a residual conflict that is not
normalised, the default configuration. Fewer operations spill fewer of the 32 + 32 + 32
live values out of the registers: the lean step is 10–16 % faster (docs/performance.md).
:func:`evperc.fusion.fused.fused_step` picks it; numba compiles a variant on its first use. The
lean kernels run a second, *road* body on sub-blocks of 16 lanes without the building label
and without mass on :data:`ROAD_ZERO` (12 subsets that cells without the building prior
never reach under lean steps, :func:`road_closure`): 20 masses instead of 32, 12–18 %
faster on a drive, where 97 % of the computed sub-blocks qualify; it doubled the lean
kernels' compile time when it came (~10 → ~19 s, once). The rows of a frame can be shared among
threads (``band``, ``bands``, ``band_rows``: chunks of rows to a thread in turn, each
writing its mass runs from its own room, ``chunk_ends``). Arrays are
flattened once and indexed with unsigned integers: a signed index gets numba's
negative-index fix-up (vector copies become scatters) and an array view costs two atomic
reference-count updates (12 % of the step's time under perf before they went). Last,
:mod:`evperc.fusion.single_assignment` gives each definition its own name and writes each
pure conditional expression as a call of ``_sel``: the same program, which numba's front end
compiles 2.2 times faster (the four kernels 63 s instead of 136 s).
"""

from __future__ import annotations

from pathlib import Path

from evperc.fusion.single_assignment import SELECT, selects, single_assignment
from evperc.output.layers import MASS_TILE

_F, _I, _U, _S, _M, _O, _OMEGA = 1, 2, 4, 8, 16, 30, 31
#: prior focal sets (evperc.geo.prior): building {I}, road {F, S, M}, other {F, U, S, M}
PRIORS = {"b": _I, "r": _F | _S | _M, "o": _F | _U | _S | _M}
TARGET = Path(__file__).with_name("kernel.py")


def road_closure() -> frozenset[int]:
    """The subsets a cell without the building label can have mass on after any number of
    lean steps (α_I = 0) from a state on the same subsets: the fixpoint, from the sets
    without I and O, Ω, of contextual discounting (A ∪ {θ}, θ ≠ I), the conjunctive
    combination with SG and the road and other priors (A ∩ B for B in {F}, O, Ω and the
    priors), the ⊛ rule (∅, {M}, Ω, and the motion gate's closed targets O and {I, U, S}:
    :func:`evperc.fusion.twin.conflict_targets`; its {I} is for building cells only) and the
    specialisation by ζ (A ∖ {M}, {M} → {S})."""
    reached = {a for a in range(32) if not a & _I} | {_O, _OMEGA}
    grown = True
    while grown:
        new = set()
        for a in reached:
            new |= {a | bit for bit in (_F, _U, _S, _M)}
            new |= {a & b for b in (_F, _O, _OMEGA, PRIORS["r"], PRIORS["o"])}
            new |= {a & ~_M, _S if a == _M else a}
        new |= {0, _M, _OMEGA, _O, _O & ~_M}
        grown = not new <= reached
        reached |= new
    return frozenset(reached)


#: subsets that stay without mass in a cell without the building label (lean options)
ROAD_ZERO = frozenset(range(32)) - road_closure()

#: numba's fast-math flags for the kernels: only those that cannot change a finite result.
#: ``nnan``/``ninf`` (no NaN or infinity reaches the body: masses are in [0, 1] and every
#: division is guarded by a select) let LLVM simplify selects and comparisons. Left out on
#: purpose, as they make a cell's bits depend on the CPU and on where the cell falls
#: (issue 17): ``arcp``/``afn`` (a vector division becomes a reciprocal *estimate* and a
#: Newton step: 1 / 1 gives 1 − 2⁻²⁴ with AVX2's ``vrcpps``, exact with AVX-512's
#: ``vrcp14ps``, so a vacuous cell stopped being exactly vacuous), ``contract`` (a·b + c
#: fused into an FMA where the CPU has one, and only in some of the loops that compute a
#: cell) and ``reassoc`` (sums reordered differently in the road body and the full body,
#: so a cell's round-off depended on its neighbours). ``nsz`` is left out too: it only
#: concerns the sign of zero, but the state's bytes are promised bit for bit. Without
#: them every operation is one IEEE-754 float32 operation in the order written here, the
#: same on any CPU numba targets (SSE2, AVX2, AVX-512, NEON).
FASTMATH = frozenset({"nnan", "ninf"})

HEADER = '''"""GENERATED by evperc/fusion/codegen.py, do not edit (python -m evperc.fusion.codegen).

Straight-line per-cell code of the fused step, vectorised by LLVM across the cells of a row.
See evperc/fusion/codegen.py for the algebra and evperc/fusion/fused.py for the API.
"""
# ruff: noqa

import numba
import numpy as np

_0 = np.float32(0.0)
_1 = np.float32(1.0)
_255 = np.float32(255.0)
_HALF = np.float32(0.5)
_TIE = np.float32(1e-4)
_TINY = np.float32(1e-30)
_INV2 = np.float32(1.0 / 2.0)
_INV3 = np.float32(1.0 / 3.0)
_INV4 = np.float32(1.0 / 4.0)
_INV5 = np.float32(1.0 / 5.0)
_2 = np.float32(2.0)
_ONE = np.uint32(1)
_OMEGA_BIT = np.uint32(1 << 31)
_ALL_PLANES = np.uint32(0xFFFFFFFF)
''' + "".join(f"_P{a} = np.float32({2 ** a})\n" for a in range(16)) + f'''


@numba.njit(cache=True)
def {SELECT}(c, a, b):  # pragma: no cover - compiled; inlined as a select
    return a if c else b


'''


#: cells per block: the body runs over a block held in one local buffer ``buf`` of planes of
#: BLOCK float32 (inputs, then outputs), so every access is ``buf[sbase + constant + l]``
#: and LLVM proves without run-time checks that the planes do not overlap
BLOCK = 256
#: floats from one plane of the block buffer to the next: BLOCK and one cache line more, so
#: that a sub-block's lanes of the 45 planes fall in different sets of the L1 cache (a
#: stride of 1 kB puts them all in 4 of its 64 sets)
STRIDE = BLOCK + 16
#: lanes per run of the body (whole sub-blocks within [l0, l1) are computed)
SUB = 16
#: cells per tile of the stored masses (evperc.output.mass_tiles): a divisor of BLOCK; smaller
#: tiles store fewer planes (the union of fewer cells' focal sets: 1.56 MB of runs per
#: frame of workload (a) with tiles of 256, 1.02 with 64, 0.83 with 32, 0.63 per cell);
#: the output format's MASS_TILE (evperc.output.layers)
TILE = MASS_TILE
IN_ZETA, IN_FREE, IN_OCC, IN_LABEL, IN_OBSERVED, IN_GATE = 32, 33, 34, 35, 36, 37
# outputs overwrite the inputs of their own lane (the body loads every input before it
# stores), which keeps the buffer in L1
OUT_MASS = 0
OUT_ZETA = 32
OUT_BETP = 33
OUT_CONFLICT = OUT_BETP + 5
OUT_CODE = OUT_CONFLICT + 3
OUT_VACUOUS = OUT_CODE + 1
#: the cell's focal sets (bit A set where c(A) ≠ 0), bits 0–15 and 16–31 as two exact floats
OUT_FOCAL_LO = OUT_VACUOUS + 1
OUT_FOCAL_HI = OUT_FOCAL_LO + 1
PLANES = OUT_FOCAL_HI + 1


def _at(plane: int) -> str:
    """Lane ``l`` of ``plane`` in the sub-block at ``sbase`` of the block buffer."""
    return f"sbase + np.uint64({plane * STRIDE} + l)"


def _sum(terms: list[str]) -> str:
    """A balanced sum (short dependency chains)."""
    if not terms:
        return "_0"
    while len(terms) > 1:
        terms = [f"({terms[k]} + {terms[k + 1]})" if k + 1 < len(terms) else terms[k]
                 for k in range(0, len(terms), 2)]
    return terms[0]


def _body(lean: bool = False, road: bool = False) -> list[str]:
    """Statements for lane ``l`` of the block in ``buf`` (decision codes as floats).
    ``lean``: for contextual discounting with α_I = 0 and a residual conflict that is not
    normalised (the defaults): the I butterfly, classical discounting and the
    normalisation, identities then, are left out. ``road`` (with ``lean``): for lanes
    without the building label whose state has no mass on :data:`ROAD_ZERO`, which then
    stay zero (:func:`road_closure`): those sets and the building prior are left out."""
    zero = ROAD_ZERO if road else frozenset()
    s: list[str] = []
    add = s.append
    for a in range(32):
        add(f"m{a} = _0" if a in zero else f"m{a} = buf[{_at(a)}]")
    add(f"z = buf[{_at(IN_ZETA)}]")
    add(f"f = buf[{_at(IN_FREE)}]")
    add(f"o = buf[{_at(IN_OCC)}]")
    add("u = _1 - f - o")
    add(f"lab = buf[{_at(IN_LABEL)}]")
    add(f"ob = buf[{_at(IN_OBSERVED)}]")
    add(f"gt = buf[{_at(IN_GATE)}]")
    add("obs = ((f > _0) | (o > _0)) if derive_obs else (ob != _0)")
    add("is_b = False" if road else "is_b = lab == _2")
    add("is_r = lab == _1")
    add("is_o = lab == _0")
    add("beta = beta_b if is_b else (beta_r if is_r else (beta_o if is_o else _0))")
    add("beta = beta if (obs | everywhere) else _0")
    add("e = beta * f if is_b else _0")
    add("kept = _1 - e")
    add("total = kept <= tol")
    add("beta = _0 if total else beta")
    add("e = _0 if total else e")
    add("kept = _1 if total else kept")
    add("inv_kept = _1 / kept")
    add("bb = beta if is_b else _0")
    add("br = beta if is_r else _0")
    add("bo = beta if is_o else _0")
    # 3. discounting: contextual butterflies (rate 0: identity), then classical
    for bit, name in ((_F, "a_f"), (_I, "a_i"), (_U, "a_u"), (_S, "a_s"), (_M, "a_m")):
        if lean and bit == _I:
            continue
        for j in range(32):
            if j & bit or j in zero:
                continue
            add(f"t = {name} * m{j}")
            add(f"m{j + bit} += t")
            add(f"m{j} -= t")
    if not lean:
        add("rest = _1 - m31")
        for a in range(31):
            add(f"m{a} *= keep_c")
        add("m31 += a_c * rest")
    # 4. d = m ∩ SG
    add("s_f = " + _sum([f"m{a}" for a in range(32) if a & _F]))
    add("s_nf = " + _sum([f"m{a}" for a in range(32) if not a & _F]))
    # dn: d without SG's {F}, which the building prior {I} sends wholly to ∅ (see below)
    add("dn0 = u * m0 + o * (m0 + m1)")
    add("dn1 = u * m1")
    add("d0 = dn0 + f * s_nf")
    add("d1 = dn1 + f * s_f")
    # where the gate is closed and faded_o, a return in a cell whose free mass has faded
    # (A ∋ F, A ≠ {F}) says O only: o·m(A) goes to O instead of A ∖ {F} (method.md §5a)
    add("kf = _1 if (gate_off | (gt != _0) | (not faded_o)) else _0")
    faded = []
    for a in range(2, 32):
        if a in zero:
            add(f"d{a} = _0")
        elif a & _F:
            add(f"d{a} = u * m{a}")
        elif a == _O:
            continue  # O: below, with the faded products
        else:
            add(f"d{a} = u * m{a} + o * (m{a} + kf * m{a + 1})")
            if a + 1 not in zero:
                faded.append(f"m{a + 1}")
    add(f"d{_O} = u * m{_O} + o * (m{_O} + m{_OMEGA} + "
        f"(_1 - kf) * {_sum(faded)})")
    # c = ((1 − β) d + Σ_P β_P (d ∩ P) − e δ∅) / kept
    add("keep_d = _1 - beta")
    for a in range(32):
        if a in zero:
            add(f"c{a} = _0")
            continue
        terms = []
        for name, prior in PRIORS.items():
            if road and name == "b":
                continue
            if a & ~prior:
                continue
            sources = [f"{'dn' if name == 'b' and x < 2 else 'd'}{x}"
                       for x in range(32) if x & prior == a]
            terms.append(f"b{name} * {_sum(sources)}")
        extra = " + " + " + ".join(terms) if terms else ""
        add(f"c{a} = (keep_d * d{a}{extra}) * inv_kept")
    # conflict parts (method.md §5.4)
    add("sg_free = f * (_1 - bb) * inv_kept")
    add("sg_bel_o = (o + u * bb) * inv_kept")
    add("pg_bel_o = " + _sum([f"m{a}" for a in range(2, 32, 2)]))
    add("fo = m1 * sg_bel_o")
    add("of = pg_bel_o * sg_free")
    add("other = c0 - fo - of")
    add("other = other if other > _0 else _0")
    # 5. rule ⊛ (residual: 0 omega, 1 empty, 2 normalise); ∅_FO to {M} where the motion
    # gate is open (or off), to {I} in building cells (bld_i), else to O or {I,U,S}
    if road:
        add("fo_m = fo if (gate_off | (gt != _0)) else _0")
        add("fo_c = _0 if (gate_off | (gt != _0)) else fo")
    else:
        add("in_b = is_b & bld_i")
        add("fo_m = _0 if in_b else (fo if (gate_off | (gt != _0)) else _0)")
        add("fo_c = _0 if (in_b | gate_off | (gt != _0)) else fo")
        add("c2 += fo if in_b else _0")
    add("c0 = other if residual == 1 else _0")
    add("c16 += fo_m")
    add("c30 += fo_c if closed_o else _0")
    add("c14 += _0 if closed_o else fo_c")
    add("c31 += of + (other if residual == 0 else _0)")
    if not lean:
        add("kept_rule = _1 - other")
        add("kept_rule = kept_rule if kept_rule > _TINY else _TINY")
        add("scale = (_1 / kept_rule) if residual == 2 else _1")
        for a in range(32):
            add(f"c{a} *= scale")
    # 6. ζ
    add("bel_o = " + _sum([f"c{a}" for a in range(2, 32, 2)]))
    add("dynamic = fo_m + of")
    add("z_up = z + inc")
    add("z_up = z_up if z_up < _1 else _1")
    add("z_down = z - dec")
    add("z_down = z_down if z_down > _0 else _0")
    add("z = z_up if ((bel_o >= gamma_o) & (dynamic <= gamma_c)) else "
        "(z_down if dynamic > gamma_c else z)")
    # 7. specialisation by ζ: A ∋ M gives ζ m(A) to A ∖ {M}; {M} to {S} or ∅
    for a in range(_M + 1, 32):
        if a in zero:
            continue
        add(f"g = c{a} * z")
        add(f"c{a} -= g")
        add(f"c{a - _M} += g")
    add("g = c16 * z")
    add("c16 -= g")
    add("c8 += g if to_s else _0")
    add("c0 += _0 if to_s else g")
    # 8. store
    for a in range(32):
        if a not in zero:  # the zero sets hold 0 in the buffer already
            add(f"buf[{_at(OUT_MASS + a)}] = c{a}")
    add(f"buf[{_at(OUT_ZETA)}] = z")
    # method.md §6: betP on the stored masses, then the decision
    add("norm = " + _sum([f"c{a}" for a in range(1, 32)]))
    add("inv_norm = (_1 / norm) if norm > tol else _0")
    inv = {1: None, 2: "_INV2", 3: "_INV3", 4: "_INV4", 5: "_INV5"}
    for a in range(1, 32):
        k = bin(a).count("1")
        add(f"w{a} = c{a}" + (f" * {inv[k]}" if inv[k] else ""))
    for name, bit in (("p_f", _F), ("p_i", _I), ("p_u", _U), ("p_s", _S), ("p_m", _M)):
        add(f"{name} = " + _sum([f"w{a}" for a in range(1, 32) if a & bit]) + " * inv_norm")
    add("static = p_i + p_u + p_s")
    add("code = c_free")
    add("best = p_f")
    add("code = c_moving if p_m > best else code")
    add("best = p_m if p_m > best else best")
    add("is_static = static > best")
    add("code = c_static if is_static else code")
    add("best = static if is_static else best")
    add("fine_code = c_infra")
    add("fine_best = p_i")
    add("fine_code = c_unmapped if p_u > fine_best else fine_code")
    add("fine_best = p_u if p_u > fine_best else fine_best")
    add("fine_code = c_stopped if p_s > fine_best else fine_code")
    add("fine_best = p_s if p_s > fine_best else fine_best")
    add("least = p_i if p_i < p_u else p_u")
    add("least = least if least < p_s else p_s")
    add("fine_second = static - fine_best - least")
    add("fine_ok = (fine_best >= _HALF) & (fine_best >= _HALF * static) & "
        "(fine_best - fine_second > _TIE)")
    add("code = fine_code if (is_static & fine_ok) else code")
    add("code = c_unknown if ((best < min_betp) | (c31 > max_ign)) else code")
    for k, name in enumerate(("p_f", "p_i", "p_u", "p_s", "p_m")):
        add(f"buf[{_at(OUT_BETP + k)}] = {name}")
    for k, name in enumerate(("fo", "of", "other")):
        add(f"buf[{_at(OUT_CONFLICT + k)}] = {name}")
    add(f"buf[{_at(OUT_CODE)}] = code")
    # the cell's focal sets: bit A where c(A) ≠ 0, bits 0–15 and 16–31 as two exact float sums
    for name, part in (("focal_lo", range(16)), ("focal_hi", range(16, 32))):
        add(f"{name} = " + _sum([f"(_P{a - part.start} if c{a} != _0 else _0)" for a in part]))
    add(f"buf[{_at(OUT_FOCAL_LO)}] = focal_lo")
    add(f"buf[{_at(OUT_FOCAL_HI)}] = focal_hi")
    # the cell is exactly vacuous with ζ = 0 (only Ω, with mass 1): a later frame may skip it
    add(f"buf[{_at(OUT_VACUOUS)}] = _1 if ((focal_lo == _0) & (focal_hi == _P15) & (c31 == _1) "
        "& (z == _0)) else _0")
    return s


def _loop(width: str, target: str, value: str, indent: str = "") -> list[str]:
    """``target`` ← ``value`` for t in [0, width); ``{i}`` in them stands for the element
    index ``base + t``. Flat arrays indexed by unsigned integers: no per-element
    negative-index fix-up (which turns vector copies into scatters) and no array views
    (each costs two atomic reference-count updates)."""
    i = "np.uint64(t)"
    return [f"{indent}for t in range({width}):",
            f"{indent}    {target.format(i=i)} = {value.format(i=i)}"]


def _segments(lines: list[str], first: str, last: str) -> list[str]:
    """``lines`` once per part of window columns [first, last) that is contiguous in the
    circular buffer: ``a0, a1`` window columns, ``sc`` the flat buffer index of window
    column ``a0`` (row ``rb``), ``lb`` its lane in the block, ``w`` the width."""
    out = ["for seg in range(2):",
           f"    a0 = {first} if seg == 0 else max({first}, wrap)",
           f"    a1 = min({last}, wrap) if seg == 0 else {last}",
           "    w = a1 - a0",
           "    if w > 0:",
           "        sc = np.uint64(rb + a0 + (off_c if seg == 0 else off_c - cols))",
           "        lb = a0 - j0"]
    return out + ["        " + line for line in lines]


def _buf(plane: str, lane: str = "l0") -> str:
    """Element ``{i}`` of ``plane`` of the block buffer from lane ``lane`` on."""
    return f"buf[np.uint64(({plane}) * STRIDE + {lane}) + {{i}}]"


def _active_lanes() -> list[str]:
    """[l0, l1): the lanes to compute, trimmed of leading and trailing cells that are
    exactly vacuous (ζ = 0), untouched by the scan and without prior (then the step leaves
    them vacuous), to whole vectors of 16 lanes; all of [0, n) unless ``may_skip``."""
    return [
        "l0 = 0",
        "l1 = n",
        "if may_skip:",
        "    for t in range(n):",
        "        act[t] = 1  # cells entering the window are vacuous",
        *["    " + line for line in _segments(
            _loop("w", "act[np.uint64(lb) + {i}]", "fl[sc + {i}]"), "s0", "s1")],
        "    for t in range(n):",
        "        act[t] = act[t] & np.uint8((fr[wb + np.uint64(t)] == _0) & "
        "(oc[wb + np.uint64(t)] == _0))",
        "    idle = 0",
        "    for t in range(n):",
        "        idle += np.int32(act[t])",
        "    if idle == n:  # the whole block stays vacuous",
        "        l0 = l1 = n",
        "    while l0 < n and act[l0] == 1:",
        "        l0 += 1",
        "    while l1 > l0 and act[l1 - 1] == 1:",
        "        l1 -= 1",
        "    if l1 > l0:",
        "        l0 = (l0 // 16) * 16",
        "        l1 = min(n, (l1 + 15) // 16 * 16)",
    ]


def _load() -> list[str]:
    """Lanes [l0, l1) of the block into ``buf``: the previous state (vacuous outside the
    previous window), ζ, the sensor grid, labels and observed cells. Compact layout: a
    plane that is zero in every buffer cell of the lanes (``old_mask``, the union of their
    focal sets) is not read, and is zeroed only if an earlier block may have left values in
    it (``dirty``): neighbouring blocks mostly use the same planes, so few are."""
    inside = ("max(s0, j0 + l0)", "min(s1, j0 + l1)")
    return [
        "old_mask = np.uint32(0)",
        *_segments(["for t in range(w):", "    old_mask |= fc[sc + np.uint64(t)]"],
                   "j0 + l0", "j0 + l1"),
        "entering = s0 > j0 + l0 or s1 < j0 + l1",
        "if entering:  # some lanes entered the window: vacuous",
        "    for a in range(31):",
        *_loop("l1 - l0", _buf("a"), "_0", "        "),
        *_loop("l1 - l0", _buf("31"), "_1", "    "),
        *_loop("l1 - l0", _buf(str(IN_ZETA)), "_0", "    "),
        "for a in range(32):",
        "    if (old_mask >> np.uint32(a)) & _ONE:",
        *["        " + line for line in _segments(
            _loop("w", _buf("a", "lb"), "st[np.uint64(a), sc + {i}]"), *inside)],
        "    elif not entering and (dirty >> np.uint32(a)) & _ONE:",
        *_loop("BLOCK", _buf("a", "0"), "_0", "        "),
        "        dirty &= ~(_ONE << np.uint32(a))",
        "dirty |= old_mask",
        *_segments(_loop("w", _buf(str(IN_ZETA), "lb"), "zt[sc + {i}]"), *inside),
        "wl = wb + np.uint64(l0)",
        *_loop("l1 - l0", _buf(str(IN_FREE)), "fr[wl + {i}]"),
        *_loop("l1 - l0", _buf(str(IN_OCC)), "oc[wl + {i}]"),
        *_loop("l1 - l0", _buf(str(IN_LABEL)), "np.float32(lbl[wl + {i}])"),
        *_loop("l1 - l0", _buf(str(IN_OBSERVED)), "np.float32(obs_f[wl + {i}])"),
        *_loop("l1 - l0", _buf(str(IN_GATE)), "np.float32(gate_f[wl + {i}])"),
    ]


def _store_state() -> list[str]:
    """The new state, ζ, vacuous flags and focal sets of lanes [l0, l1) back into the
    circular buffer; a plane is written where some lane's cell had or has mass on it."""
    masks = ["for t in range(w):",
             f"    v = np.uint32({_buf(str(OUT_FOCAL_LO), 'lb').format(i='np.uint64(t)')})",
             f"    v |= np.uint32({_buf(str(OUT_FOCAL_HI), 'lb').format(i='np.uint64(t)')})"
             " << np.uint32(16)",
             "    fc[sc + np.uint64(t)] = v",
             "    new_mask |= v"]
    return [
        "new_mask = np.uint32(0)",
        *_segments(masks, "j0 + l0", "j0 + l1"),
        "write_mask = old_mask | new_mask",
        "# planes the body may have left non-zero in some lane of the buffer (all when it ran",
        "# past l1, on lanes whose stale inputs are not known)",
        "dirty |= new_mask if l1 % SUB == 0 else _ALL_PLANES",
        "for a in range(32):",
        "    if (write_mask >> np.uint32(a)) & _ONE:",
        *["        " + line for line in _segments(
            _loop("w", "st[np.uint64(a), sc + {i}]", _buf(f"{OUT_MASS} + a", "lb")),
            "j0 + l0", "j0 + l1")],
        *_segments(_loop("w", "zt[sc + {i}]", _buf(str(OUT_ZETA), "lb"))
                   + _loop("w", "fl[sc + {i}]", f"np.uint8({_buf(str(OUT_VACUOUS), 'lb')})"),
                   "j0 + l0", "j0 + l1"),
    ]


def _skipped(kind: str, first: str, last: str) -> list[str]:
    """Lanes [first, last) not computed: cells that entered the window (outside [s0, s1))
    become vacuous in the buffer (the others are vacuous already); outputs of a vacuous
    cell (betP 1/5, no conflict)."""
    clear = ["for a in range(31):",
             *_loop("w", "st[np.uint64(a), sc + {i}]", "_0", "    "),
             *_loop("w", "st[np.uint64(31), sc + {i}]", "_1"),
             *_loop("w", "zt[sc + {i}]", "_0"),
             *_loop("w", "fl[sc + {i}]", "np.uint8(1)"),
             *_loop("w", "fc[sc + {i}]", "_OMEGA_BIT")]
    lines = (_segments(clear, f"j0 + {first}", f"min(s0, j0 + {last})")
             + _segments(clear, f"max(s1, j0 + {first})", f"j0 + {last}"))
    width = f"{last} - {first}"
    lines.append(f"ws = wb + np.uint64({first})")
    if kind == "float":
        return lines + ["for k in range(5):",
                        *_loop(width, "bp[np.uint64(k), ws + {i}]", "_INV5", "    "),
                        "for k in range(3):",
                        *_loop(width, "cf[np.uint64(k), ws + {i}]", "_0", "    "),
                        *_loop(width, "dc[ws + {i}]", "vac_code")]
    return lines + ["for k in range(5):",
                    *_loop(width, "qb[np.uint64(k), ws + {i}]", "np.uint8(51)", "    "),
                    "for k in range(3):",
                    *_loop(width, "qc[np.uint64(k), ws + {i}]", "np.uint8(0)", "    "),
                    *_loop(width, "qz[ws + {i}]", "np.uint8(0)"),
                    *_loop(width, "qd[ws + {i}]", "vac_code")]


def _store_outputs(kind: str) -> list[str]:
    """Lanes [l0, l1) of the block's outputs into row ``r`` of the output arrays."""
    width = "l1 - l0"
    code = f"np.uint8({_buf(str(OUT_CODE))})"
    if kind == "float":
        return ["for k in range(5):",
                *_loop(width, "bp[np.uint64(k), wl + {i}]", _buf(f"{OUT_BETP} + k"), "    "),
                "for k in range(3):",
                *_loop(width, "cf[np.uint64(k), wl + {i}]", _buf(f"{OUT_CONFLICT} + k"),
                       "    "),
                *_loop(width, "dc[wl + {i}]", code)]

    return [*_store_tile(),
            "for k in range(5):",
            *_quantised(width, "qb[np.uint64(k), wl + {i}]", f"{OUT_BETP} + k"),
            "for k in range(3):",
            *_quantised(width, "qc[np.uint64(k), wl + {i}]", f"{OUT_CONFLICT} + k"),
            *_quantised(width, "qz[wl + {i}]", str(OUT_ZETA), indent=""),
            *_loop(width, "qd[wl + {i}]", code)]


def _quantised(width: str, target: str, plane: str, lane: str = "l0",
               indent: str = "    ") -> list[str]:
    """``target`` ← round(255 · clip(x, 0, 1)) (as evperc.output.quantise) of ``width`` lanes
    of ``plane`` of the block buffer from lane ``lane`` on; ``{i}`` as in :func:`_loop`."""
    return [f"{indent}for t in range({width}):",
            f"{indent}    v = {_buf(plane, lane).format(i='np.uint64(t)')}",
            f"{indent}    v = v if v > _0 else _0",
            f"{indent}    v = v if v < _1 else _1",
            f"{indent}    {target.format(i='np.uint64(t)')} = "
            "np.uint8(np.int32(v * _255 + _HALF))"]


def _store_tile() -> list[str]:
    """The block's masses as runs of the output's block-sparse layout
    (:mod:`evperc.output.mass_tiles`), one tile of TILE lanes after the other: the tile's mask
    is the union of its cells' focal sets (Ω for lanes not computed, which are vacuous),
    then for each plane in it, in increasing subset order, the quantised values of the
    tile's cells, from ``pos`` on."""
    focal = (f"np.uint32({_buf(str(OUT_FOCAL_LO), '0')}) | "
             f"(np.uint32({_buf(str(OUT_FOCAL_HI), '0')}) << np.uint32(16))")
    return [
        "for q0 in range(0, n, TILE):",
        "    q1 = min(n, q0 + TILE)",
        "    lane0 = min(max(l0, q0), q1)  # [lane0, lane1): the tile's computed lanes",
        "    lane1 = max(min(l1, q1), lane0)",
        "    tile_mask = _OMEGA_BIT if (lane0 > q0 or lane1 < q1) else np.uint32(0)",
        "    for t in range(lane0, lane1):",
        f"        tile_mask |= {focal.format(i='np.uint64(t)')}",
        "    qt[tile + np.uint64(q0 // TILE)] = tile_mask",
        "    for a in range(32):",
        "        if (tile_mask >> np.uint32(a)) & _ONE:",
        "            value = np.uint8(255) if a == 31 else np.uint8(0)",
        "            for t in range(q0, lane0):",
        "                qr[pos + np.uint64(t - q0)] = value",
        "            pl = pos + np.uint64(lane0 - q0)",
        *_quantised("lane1 - lane0", "qr[pl + {i}]", f"{OUT_MASS} + a", "lane0", " " * 12),
        "            for t in range(lane1, q1):",
        "                qr[pos + np.uint64(t - q0)] = value",
        "            pos += np.uint64(q1 - q0)",
    ]


def _idle_tile() -> list[str]:
    """An idle block's masses: all its cells are vacuous, its tiles hold Ω only."""
    return ["for q0 in range(0, n, TILE):",
            "    qt[tile + np.uint64(q0 // TILE)] = _OMEGA_BIT",
            "for t in range(n):",
            "    qr[pos + np.uint64(t)] = np.uint8(255)",
            "pos += np.uint64(n)"]


PARAMS = ("derive_obs, everywhere, beta_b, beta_r, beta_o, tol, a_f, a_i, a_u, a_s, a_m, "
          "keep_c, a_c, residual, to_s, inc, dec, gamma_o, gamma_c, min_betp, max_ign, "
          "c_free, c_moving, c_static, c_infra, c_unmapped, c_stopped, c_unknown, vac_code, "
          "may_skip, gate_off, bld_i, closed_o, faded_o")


def _kernel(kind: str, lean: bool = False) -> list[str]:
    outs = ("betp, conflict, decision" if kind == "float"
            else "q_runs, q_tiles, q_length, q_betp, q_conflict, q_zeta, q_decision")
    flat = ["bp = betp.reshape(5, n_cells)", "cf = conflict.reshape(3, n_cells)",
            "dc = decision.reshape(n_cells)"] if kind == "float" else [
            "qr = q_runs", "qt = q_tiles.reshape(q_tiles.size)",
            "pos = np.uint64(0)  # bytes of mass runs written", "qb = q_betp.reshape(5, n_cells)",
            "qc = q_conflict.reshape(3, n_cells)", "qz = q_zeta.reshape(n_cells)",
            "qd = q_decision.reshape(n_cells)"]
    block = [
        "n = min(BLOCK, cols - j0)",
        "s0 = max(lo, j0)  # [s0, s1): cells of the block inside the previous window",
        "s1 = min(hi, j0 + n)",
        "wb = np.uint64(r * cols + j0)  # flat window index of the block's lane 0",
        "tile = np.uint64(r * tiles_per_row + j0 // TILE)  # the block's first tile",
        *_active_lanes(),
        "if l1 <= l0:",
        "    l0 = l1 = n",
        "if l0 > 0:",
        *["    " + line for line in _skipped(kind, "0", "l0")],
        "if l1 < n:",
        *["    " + line for line in _skipped(kind, "l1", "n")],
        "if l1 <= l0:",
        *(["    " + line for line in _idle_tile()] if kind == "stored" else []),
        "    continue",
        *_load(),
    ]
    lines = [
        "",
        "",
        "@numba.njit(cache=True, nogil=True, fastmath={"
        + ", ".join(f"'{flag}'" for flag in sorted(FASTMATH)) + "}, error_model=\"numpy\")",
        f"def step_{kind}{'_lean' if lean else ''}(state, zeta, flags, focal, off_r, off_c, dr, "
        "dc_, free, occ, labels,",
        f"               observed, gate, {PARAMS}, {outs}, band, bands, band_rows, chunk_ends):"
        "  # pragma: no cover - compiled",
        "    rows, cols = state.shape[1], state.shape[2]",
        "    n_cells = rows * cols",
        "    st = state.reshape(32, n_cells)",
        "    zt = zeta.reshape(n_cells)",
        "    fl = flags.reshape(n_cells)",
        "    fc = focal.reshape(n_cells)",
        "    fr = free.reshape(n_cells)",
        "    oc = occ.reshape(n_cells)",
        "    lbl = labels.reshape(n_cells)",
        "    obs_f = observed.reshape(n_cells)",
        "    gate_f = gate.reshape(n_cells)",
        *["    " + line for line in flat],
        "    wrap = cols - off_c  # window columns from here on wrap to the buffer's start",
        "    tiles_per_row = (cols + TILE - 1) // TILE",
        "    buf = np.zeros(PLANES * STRIDE, np.float32)",
        "    act = np.zeros(BLOCK, np.uint8)",
        "    dirty = np.uint32(0)  # planes that may be non-zero in some lane of buf",
        "    for r in range(rows):",
        "        chunk = r // band_rows",
        "        if chunk % bands != band:",
        "            continue",
        *(["        if r == chunk * band_rows:  # a chunk's runs start at its room",
           "            pos = np.uint64(32 * cols * r)"] if kind == "stored" else []),
        "        buf_row = r + off_r",
        "        buf_row = buf_row - rows if buf_row >= rows else buf_row",
        "        rb = buf_row * cols",
        "        lo = min(max(-dc_, 0), cols)",
        "        hi = max(min(cols - dc_, cols), lo)",
        "        if r + dr < 0 or r + dr >= rows:",
        "            lo = hi = 0",
        "        for j0 in range(0, cols, BLOCK):",
    ]
    lines += ["            " + line for line in block]
    # sub-blocks of SUB lanes: a loop of constant trip count over constant offsets from one
    # unsigned base, which LLVM vectorises without run-time overlap checks
    if lean:  # planes of ROAD_ZERO some lane has mass on
        lines += ["            zero_planes = old_mask & ROAD_ZERO_MASK"]
    lines += ["            for sub in range(l0 // SUB, (l1 + SUB - 1) // SUB):",
              "                sbase = np.uint64(sub * SUB)"]
    if lean:  # sub-blocks without building lanes and mass on ROAD_ZERO: the road body
        lines += ["                not_road = np.uint8(0)  # a building lane or mass on ROAD_ZERO",
                  "                for l in range(SUB):",
                  f"                    not_road |= np.uint8(buf[{_at(IN_LABEL)}] == _2)",
                  "                if not_road == 0 and zero_planes != 0:",
                  "                    for a in range(32):",
                  "                        if (zero_planes >> np.uint32(a)) & _ONE:",
                  "                            for l in range(SUB):",
                  "                                not_road |= np.uint8(buf[sbase + np.uint64(a) * "
                  "np.uint64(STRIDE) + np.uint64(l)] != _0)",
                  "                if not_road == 0:",
                  "                    for l in range(SUB):"]
        lines += ["                        " + line for line in _body(lean, road=True)]
        lines += ["                    continue"]
    lines += ["                for l in range(SUB):"]
    lines += ["                    " + line for line in _body(lean)]
    lines += ["            " + line for line in _store_state() + _store_outputs(kind)]
    if kind == "stored":
        lines += ["        if r == min(rows, (chunk + 1) * band_rows) - 1:",
                  "            chunk_ends[chunk] = np.int64(pos)",
                  "    if bands == 1:",
                  "        q_length[0] = np.int64(pos)"]
    return lines


def source() -> str:
    """The text of evperc/fusion/kernel.py."""
    constants = (f"BLOCK = {BLOCK}\nSTRIDE = {STRIDE}\nSUB = {SUB}\nPLANES = {PLANES}\n"
                 f"TILE = {TILE}\n"
                 f"ROAD_ZERO_MASK = np.uint32({sum(1 << a for a in sorted(ROAD_ZERO)):#x})\n")
    kernels = [line for lean in (False, True) for kind in ("float", "stored")
               for line in _kernel(kind, lean)]
    # one name per definition and selects: the same program, compiled 2.2x faster
    return selects(single_assignment(HEADER + constants + "\n".join(kernels) + "\n"))


def main() -> None:
    TARGET.write_text(source())


if __name__ == "__main__":
    main()
