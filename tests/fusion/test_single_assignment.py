"""evperc.fusion.single_assignment: the rewritten source is the same program (the original,
run by Python, is the oracle), renames only where that is provable, and the generated kernels
are in its final form."""

from __future__ import annotations

import ast
import random
import textwrap
from collections import Counter

import pytest

from evperc.fusion import codegen
from evperc.fusion.single_assignment import SELECT, selects, single_assignment


def _sel(c, a, b):
    return a if c else b


def compiled(source: str, name: str = "f"):
    namespace = {SELECT: _sel, "min": min, "max": max}
    exec(compile(source, "<test>", "exec"), namespace)  # noqa: S102 - our own test source
    return namespace[name]


def rewrite(source: str) -> str:
    return selects(single_assignment(source))


def stores(source: str, fn: str = "f") -> Counter:
    """How many times each name is assigned (statically) in function ``fn``."""
    tree = next(n for n in ast.parse(source).body if getattr(n, "name", None) == fn)
    return Counter(n.id for n in ast.walk(tree)
                   if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store))


STRAIGHT = textwrap.dedent("""
    def f(a, b):
        m = a + b
        t = m * 2
        m -= t
        t = a * m
        m += t  # a comment that stays
        c = m if m > b else b
        return m, t, c
""")


def test_straight_line_updates_get_one_name_each() -> None:
    out = rewrite(STRAIGHT)
    assert max(stores(out).values()) == 1
    assert "# a comment that stays" in out
    assert f"{SELECT}(" in out
    for a in range(-5, 6):
        for b in range(-5, 6):
            assert compiled(out)(a, b) == compiled(STRAIGHT)(a, b)


LOOPS = textwrap.dedent("""
    def f(n, xs):
        acc = 0
        for t in range(n):
            acc += t * 2
        for t in range(n, 2 * n):
            acc -= t
        total = 0
        for i in range(n):
            total += xs[i]
            if total > 3:
                total = total - 1
        k = n
        if n > 2:
            k = n + 1
        x = xs[0] if n > 0 else 0
        y = max(xs) if n > 0 else 0
        z = xs.count(0) if n > 0 else 0
        return acc, total, k, x, y, z
""")


def test_loop_carried_and_nested_names_keep_their_names() -> None:
    """A loop's own variable gets a name per loop; a variable carried round a loop
    (``acc``, ``total``), assigned in a nested block (``k``) or guarding an index (``x``)
    is left as it is."""
    out = rewrite(LOOPS)
    counts = stores(out)
    assert counts["acc"] == 3 and counts["total"] == 3 and counts["k"] == 2
    assert "t" not in counts and counts["t_1"] == counts["t_2"] == 1
    assert f"{SELECT}(" not in out  # xs[0], max(xs) may not be evaluated when n == 0
    for n in range(0, 7):
        xs = list(range(3, 3 + n))
        assert compiled(out)(n, xs) == compiled(LOOPS)(n, xs)


def test_a_new_name_never_takes_an_existing_one() -> None:
    source = textwrap.dedent("""
        def f(a):
            m = a
            m_1 = 10
            m += m_1
            m *= 3
            return m, m_1
    """)
    out = rewrite(source)
    assert max(stores(out).values()) == 1
    assert compiled(out)(4) == compiled(source)(4) == (42, 10)


def test_a_name_read_before_its_run_assigns_it_keeps_its_name() -> None:
    """Live on entry to the run (assigned before the loop, read first in its body): kept."""
    source = textwrap.dedent("""
        def f(n):
            a = 1
            for i in range(n):
                a += i
                a = a * 2
            return a
    """)
    assert rewrite(source) == source


def test_a_loop_variable_its_body_assigns_keeps_its_name() -> None:
    """The body's assignment may not run (it is nested): its later reads need the name."""
    source = textwrap.dedent("""
        def f(n):
            s = 0
            for t in range(n):
                if t > 1:
                    t = 10
                s = s + t
            for t in range(n):
                s -= t
            return s
    """)
    out = rewrite(source)
    assert stores(out)["t"] == 3
    for n in range(5):
        assert compiled(out)(n) == compiled(source)(n)


def test_names_bound_otherwise_keep_their_names() -> None:
    """``:=`` and ``global`` bind names the rewrite does not follow: left alone."""
    source = textwrap.dedent("""
        G = 0
        def f(a):
            global G
            x = 1
            y = (x := a + 5) + x
            z = x
            x = z * 2
            G = a
            G = G + 1
            return x, y, z
    """)
    out = rewrite(source)
    assert stores(out)["x"] == 3 and stores(out)["G"] == 2
    namespace_in, namespace_out = {}, {}
    exec(compile(source, "<in>", "exec"), namespace_in)  # noqa: S102 - our own test source
    exec(compile(out, "<out>", "exec"), namespace_out)  # noqa: S102
    assert namespace_out["f"](3) == namespace_in["f"](3) == (16, 16, 8)
    assert namespace_out["G"] == namespace_in["G"] == 4


def test_two_statements_on_a_line_are_refused() -> None:
    with pytest.raises(ValueError, match="alone on its line"):
        single_assignment("def f(a):\n    m = a; m += 1\n    return m\n")


# random programs: straight-line runs, loops, nested blocks, conditional expressions
def _expr(rng: random.Random, names: list[str], depth: int = 0) -> str:
    pick = rng.random()
    if depth > 2 or pick < 0.35:
        return rng.choice(names) if rng.random() < 0.8 else str(rng.randint(-3, 3))
    if pick < 0.55:
        return (f"({_expr(rng, names, depth + 1)} if {rng.choice(names)} > "
                f"{_expr(rng, names, depth + 1)} else {_expr(rng, names, depth + 1)})")
    if pick < 0.65:
        return f"min({_expr(rng, names, depth + 1)}, {_expr(rng, names, depth + 1)})"
    op = rng.choice(["+", "-", "*"])
    return f"({_expr(rng, names, depth + 1)} {op} {_expr(rng, names, depth + 1)})"


def _block(rng: random.Random, names: list[str], indent: str, depth: int) -> list[str]:
    lines = []
    for _ in range(rng.randint(1, 7)):
        kind = rng.random()
        if kind < 0.45 or depth > 1:
            target = rng.choice(["m0", "m1", "m2", "t", f"v{rng.randint(0, 3)}"])
            if target in names and rng.random() < 0.5:
                lines.append(f"{indent}{target} {rng.choice(['+=', '-=', '*='])} "
                             f"{_expr(rng, names)}")
            else:
                lines.append(f"{indent}{target} = {_expr(rng, names)}")
                names.append(target)
        elif kind < 0.7:
            var = rng.choice(["t", "i"])
            lines.append(f"{indent}for {var} in range({rng.randint(0, 3)}):")
            lines += _block(rng, [*names, var], indent + "    ", depth + 1)
        elif kind < 0.85:
            lines.append(f"{indent}if {_expr(rng, names)} > {_expr(rng, names)}:")
            lines += _block(rng, list(names), indent + "    ", depth + 1)
        else:
            lines.append(f"{indent}x = xs[{rng.choice(names)} % 3] if "
                         f"{rng.choice(names)} > 0 else 0")
            names.append("x")
    return lines


def _program(seed: int) -> str:
    rng = random.Random(seed)
    names = ["a", "b"]
    lines = ["def f(a, b, xs):", "    m0 = m1 = m2 = t = v0 = v1 = v2 = v3 = x = i = 0",
             *_block(rng, names, "    ", 0),
             "    return m0, m1, m2, t, v0, v1, v2, v3, x, i"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("seed", range(300))
def test_random_programs_compute_the_same(seed: int) -> None:
    """300 random programs (integers, so that any reordering or wrong version shows), each
    run on a grid of inputs: the rewritten program returns what the original returns."""
    source = _program(seed)
    out = rewrite(source)
    ast.parse(out)
    original, rewritten = compiled(source), compiled(out)
    for a in (-2, 0, 1, 3):
        for b in (-1, 0, 2):
            xs = [a, b, a - b]
            assert rewritten(a, b, xs) == original(a, b, xs), (source, out)


def test_the_random_programs_exercise_the_rewrites() -> None:
    """The programs above do get renamed and selected (else their test would prove nothing)."""
    pairs = [(_program(seed), rewrite(_program(seed))) for seed in range(300)]
    assert sum(f"{SELECT}(" in out for _, out in pairs) > 200
    assert sum(bool(set(stores(out)) - set(stores(source))) for source, out in pairs) > 100


def test_the_generated_kernels_are_in_final_form() -> None:
    """evperc/fusion/kernel.py: rewriting it again changes nothing, every kernel's per-cell
    bodies (the loops over a sub-block's lanes) assign each name once, and few names of the
    code around them are assigned more than once (numba's front end pays a pass over the
    whole function for each: 392 in the lean stored kernel before the rewrite)."""
    text = codegen.TARGET.read_text()
    assert rewrite(text) == text
    kernels = [fn for fn in ast.parse(text).body
               if isinstance(fn, ast.FunctionDef) and fn.name.startswith("step_")]
    assert len(kernels) == 4
    for fn in kernels:
        counts = Counter(n.id for n in ast.walk(fn)
                         if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store))
        lanes = [loop for loop in ast.walk(fn) if isinstance(loop, ast.For)
                 and isinstance(loop.target, ast.Name) and loop.target.id.startswith("l")
                 and len(loop.body) > 100]  # the bodies, not the loops that OR lane flags
        in_bodies = {n.id for loop in lanes for stmt in loop.body for n in ast.walk(stmt)
                     if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store)}
        assert len(in_bodies) > 300  # the bodies were found
        assert not [name for name in in_bodies if counts[name] > 1], fn.name
        assert sum(count > 1 for count in counts.values()) <= 20, fn.name
