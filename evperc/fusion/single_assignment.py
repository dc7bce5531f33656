"""The generated kernels' source in the form numba compiles fastest: one name per definition,
pure conditional expressions as calls of one select function.

numba's front end (SSA reconstruction, the liveness and reaching-definition analyses its
passes repeat) costs, per variable assigned more than once, a walk over every basic block of
the function, and every conditional expression ``a if c else b`` makes three blocks and one
such variable. The generated kernels (:mod:`evperc.fusion.codegen`) update 32 masses in
place through straight-line code and select with conditional expressions: 392 variables
assigned more than once over 922 blocks in the lean stored kernel, 45–49 s to compile. Two
rewrites of the source, each the same program:

- :func:`single_assignment`: a variable whose every use lies in a straight-line run of simple
  statements that assigns it before reading it, or in the body of a ``for`` loop over it
  that does not assign it, gets a new name at each definition (``m3 += t`` becomes
  ``m3_2 = m3_1 + t_5``). Anything else — a variable read in a nested statement, carried
  round a loop, live on entry or a parameter — keeps its name.
- :func:`selects`: a conditional expression whose two branches read no array element and
  call nothing but numpy's numeric casts and ``min`` / ``max`` of scalars becomes
  ``_sel(c, a, b)``, a compiled
  function returning ``a if c else b`` that LLVM inlines as the select instruction it had
  made of the branch. Both branches are evaluated: only pure branches qualify (no index
  that the condition guards, no call with effects; float arithmetic under numba's numpy
  error model does not raise).

Together: 25 variables assigned more than once over 379 blocks, the lean stored kernel
compiled in 20–21 s (docs/performance.md § "The kernels' compile time"; ``python
benchmarks/compile_time.py``, which also finds no call left to ``_sel`` in the final LLVM
IR); the step's speed and its bits are unchanged (tests/fusion: the twin, the per-cell
reference, the goldens).
"""

from __future__ import annotations

import ast
from collections import defaultdict
from dataclasses import dataclass, field

#: the function :func:`selects` calls; the generated module defines it (codegen.HEADER)
SELECT = "_sel"
_SIMPLE = (ast.Assign, ast.AugAssign, ast.Expr, ast.Pass, ast.Return)
#: numpy's numeric casts (``np.float32(x)``), and the builtins of two or more scalars
_PURE_CASTS = frozenset({"float32", "float64", "uint8", "uint32", "uint64", "int32", "int64"})
_PURE_BUILTINS = frozenset({"min", "max"})


@dataclass
class _Uses:
    """Every reference to one variable: (owner, Name node, is a store), in program order;
    ``fixed``: the variable keeps its name."""
    refs: list[tuple[tuple, ast.Name, bool]] = field(default_factory=list)
    fixed: bool = False


def _simple_refs(stmt: ast.stmt) -> list[tuple[ast.Name, bool]]:
    """The Name nodes of a simple statement in evaluation order, ``True`` for a store: the
    value's names, then the target's (an augmented target is read, then stored)."""
    def names(node: ast.AST | None) -> list[ast.Name]:
        return [] if node is None else [n for n in ast.walk(node) if isinstance(n, ast.Name)]

    if isinstance(stmt, ast.Assign):
        targets = [n for t in stmt.targets for n in names(t)]
        return ([(n, False) for n in names(stmt.value)]
                + [(n, False) for n in targets if not isinstance(n.ctx, ast.Store)]
                + [(n, True) for n in targets if isinstance(n.ctx, ast.Store)])
    if isinstance(stmt, ast.AugAssign) and isinstance(stmt.target, ast.Name):
        return [(n, False) for n in names(stmt.value)] + [(stmt.target, False),
                                                          (stmt.target, True)]
    return [(n, False) for n in names(stmt)]


class _Owners:
    """Who owns each reference: a straight-line run (``("run", id(list), k)``) or a ``for``
    loop over the variable (``("for", id(loop))``)."""

    def __init__(self) -> None:
        self.uses: dict[str, _Uses] = defaultdict(_Uses)

    def visit(self, stmts: list[ast.stmt], loops: dict[str, tuple]) -> None:
        run, first_is_store = 0, {}
        for stmt in stmts:
            if isinstance(stmt, _SIMPLE):
                for node, store in _simple_refs(stmt):
                    self._simple(node, store, ("run", id(stmts), run), loops, first_is_store)
                continue
            run, first_is_store = run + 1, {}
            if isinstance(stmt, ast.For):
                self._header(stmt.iter, loops)
                inner = dict(loops)
                if isinstance(stmt.target, ast.Name):
                    inner[stmt.target.id] = ("for", id(stmt))
                    self.uses[stmt.target.id].refs.append((inner[stmt.target.id], stmt.target,
                                                           True))
                else:
                    self._header(stmt.target, {})
                self.visit(stmt.body, inner)
                self.visit(stmt.orelse, loops)
            elif isinstance(stmt, (ast.If, ast.While)):
                self._header(stmt.test, loops)
                self.visit(stmt.body, loops)
                self.visit(stmt.orelse, loops)
            else:  # return, break, continue, with, ...: their names keep their names
                self._header(stmt, {})

    def _simple(self, node: ast.Name, store: bool, run: tuple, loops: dict[str, tuple],
                first_is_store: dict[str, bool]) -> None:
        uses = self.uses[node.id]
        if node.id in loops and not first_is_store.get(node.id):
            uses.fixed |= store  # a loop body assigning its own loop variable
            uses.refs.append((loops[node.id], node, store))
            return
        if node.id not in first_is_store:
            first_is_store[node.id] = store
            uses.fixed |= not store  # read before the run assigns it
        uses.refs.append((run, node, store))

    def _header(self, expr: ast.AST, loops: dict[str, tuple]) -> None:
        for node in ast.walk(expr):
            if isinstance(node, ast.Name):
                if node.id in loops:
                    self.uses[node.id].refs.append((loops[node.id], node, False))
                else:
                    self.uses[node.id].fixed = True


def _bound_otherwise(fn: ast.FunctionDef) -> set[str]:
    """Names bound other than by an assignment or a ``for``: parameters, ``:=``, imports,
    ``global`` / ``nonlocal``, nested definitions, exception handlers. They keep their names."""
    args = fn.args
    names = {a.arg for a in (*args.posonlyargs, *args.args, *args.kwonlyargs)}
    names |= {a.arg for a in (args.vararg, args.kwarg) if a is not None}
    for node in ast.walk(fn):
        if isinstance(node, ast.NamedExpr) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, (ast.Global, ast.Nonlocal)):
            names.update(node.names)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((alias.asname or alias.name).split(".")[0] for alias in node.names)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) \
                and node is not fn:
            names.add(node.name)
        elif isinstance(node, ast.ExceptHandler) and node.name:
            names.add(node.name)
    return names


def _new_names(fn: ast.FunctionDef) -> tuple[dict[int, str], dict[int, str]]:
    """``id(Name) → new name`` for the references of every variable that may be renamed,
    and ``id(augmented target) → the name it reads``."""
    owners = _Owners()
    owners.visit(fn.body, {})
    bound = _bound_otherwise(fn)
    for name in bound:
        owners.uses[name].fixed = True
    taken = {n.id for n in ast.walk(fn) if isinstance(n, ast.Name)} | bound
    new_name: dict[int, str] = {}
    reads: dict[int, str] = {}
    for name, uses in owners.uses.items():
        if uses.fixed or sum(store for _, _, store in uses.refs) < 2:
            continue
        current: dict[tuple, str] = {}
        version = 0
        for owner, node, store in uses.refs:
            if store:
                if id(node) in new_name:
                    reads[id(node)] = new_name[id(node)]
                version += 1
                while f"{name}_{version}" in taken:
                    version += 1
                current[owner] = f"{name}_{version}"
                taken.add(current[owner])
            new_name[id(node)] = current[owner]
    return new_name, reads


def _replace(lines: list[str], stmt: ast.stmt, text: str, done: set[int]) -> None:
    """Statement ``stmt`` (alone on its line) written as ``text``, keeping its indentation
    and any comment after it; ``done``: the lines rewritten so far."""
    if stmt.lineno != stmt.end_lineno or stmt.lineno in done:
        raise ValueError(f"line {stmt.lineno}: a rewritten statement must be alone on its line")
    done.add(stmt.lineno)
    line = lines[stmt.lineno - 1]
    lines[stmt.lineno - 1] = line[:stmt.col_offset] + text + line[stmt.end_col_offset:]


def single_assignment(source: str) -> str:
    """``source`` with one name per definition where that is the same program (module
    docstring): a renamed augmented assignment ``x op= v`` is written ``x_k = x_j op (v)``."""
    lines = source.split("\n")
    done: set[int] = set()
    header_edits: dict[int, list[tuple[int, int, str]]] = defaultdict(list)
    for fn in ast.parse(source).body:
        if not isinstance(fn, ast.FunctionDef):
            continue
        new_name, reads = _new_names(fn)
        for stmt in ast.walk(fn):
            if not isinstance(stmt, ast.stmt) or stmt is fn:
                continue
            if isinstance(stmt, _SIMPLE):
                names = [n for n in ast.walk(stmt)
                         if isinstance(n, ast.Name) and id(n) in new_name]
                if not names:
                    continue
                for node in names:
                    if id(node) not in reads:
                        node.id = new_name[id(node)]
                if isinstance(stmt, ast.AugAssign) and id(stmt.target) in reads:
                    stmt = ast.Assign(
                        targets=[ast.Name(new_name[id(stmt.target)], ast.Store())],
                        value=ast.BinOp(ast.Name(reads[id(stmt.target)], ast.Load()), stmt.op,
                                        stmt.value),
                        lineno=stmt.lineno, col_offset=stmt.col_offset,
                        end_lineno=stmt.end_lineno, end_col_offset=stmt.end_col_offset)
                _replace(lines, stmt, ast.unparse(stmt), done)
            else:
                heads = ([stmt.target, stmt.iter] if isinstance(stmt, ast.For)
                         else [stmt.test] if isinstance(stmt, (ast.If, ast.While)) else [])
                for node in (n for h in heads for n in ast.walk(h)):
                    if isinstance(node, ast.Name) and id(node) in new_name:
                        header_edits[node.lineno].append(
                            (node.col_offset, node.end_col_offset, new_name[id(node)]))
    for lineno, edits in header_edits.items():
        if lineno in done:
            raise ValueError(f"line {lineno}: a rewritten statement must be alone on its line")
        line = lines[lineno - 1]
        for start, end, name in sorted(set(edits), reverse=True):
            line = line[:start] + name + line[end:]
        lines[lineno - 1] = line
    return "\n".join(lines)


def _pure_call(call: ast.Call) -> bool:
    """``np.<cast>(x)``, or ``min`` / ``max`` of two or more values (one argument would be a
    sequence, whose minimum may raise)."""
    func = call.func
    if call.keywords:
        return False
    if isinstance(func, ast.Attribute):
        return (isinstance(func.value, ast.Name) and func.value.id == "np"
                and func.attr in _PURE_CASTS and len(call.args) == 1)
    return isinstance(func, ast.Name) and func.id in _PURE_BUILTINS and len(call.args) >= 2


def _pure(expr: ast.expr) -> bool:
    """Evaluating ``expr`` reads no array element and calls nothing that may raise or have
    an effect."""
    for node in ast.walk(expr):
        if isinstance(node, (ast.Subscript, ast.Lambda, ast.NamedExpr, ast.Starred)):
            return False
        if isinstance(node, ast.Call) and not _pure_call(node):
            return False
    return True


class _Selects(ast.NodeTransformer):
    def __init__(self) -> None:
        self.count = 0

    def visit_IfExp(self, node: ast.IfExp) -> ast.expr:
        self.generic_visit(node)
        if not (_pure(node.body) and _pure(node.orelse)):
            return node
        self.count += 1
        return ast.Call(ast.Name(SELECT, ast.Load()), [node.test, node.body, node.orelse], [])


def selects(source: str) -> str:
    """``source`` with each pure conditional expression of an assignment's value written as a
    call of :data:`SELECT` (module docstring)."""
    lines = source.split("\n")
    done: set[int] = set()
    for stmt in ast.walk(ast.parse(source)):
        if isinstance(stmt, (ast.Assign, ast.AugAssign)):
            rewrite = _Selects()
            stmt.value = rewrite.visit(stmt.value)
            if rewrite.count:
                _replace(lines, stmt, ast.unparse(stmt), done)
    return "\n".join(lines)
