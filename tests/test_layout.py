"""The package's layout (docs/architecture.md): each folder one stage of the data's walk,
imports only upstream, and no import cycle between modules. Read from the source with ast,
so that a lazy import inside a function counts as well."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "evperc"

#: what each stage may import of evperc besides itself and the shared modules
#: (evperc.dst, evperc.errors, evperc.config): the stages upstream of it
ALLOWED = {
    "logs": set(),
    "geo": set(),
    "sensor": {"geo"},
    "output": {"geo", "render"},  # export colours its grids as render does
    "fusion": {"geo", "output"},  # the kernel writes the output format's layers
    "objects": {"geo", "sensor", "fusion", "output"},  # after the step: decisions → points
    "render": {"geo", "output", "fusion"},
    "eval": {"geo", "output", "fusion", "sim"},
    "sim": {"geo", "logs", "output", "fusion"},
}
SHARED = {"dst", "errors", "config", "progress", "gil_kept", "__init__"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def _imports() -> dict[str, set[str]]:
    """evperc module → the evperc modules it imports (anywhere in its body)."""
    graph: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        name = _module_name(path)
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith(
                    "evperc"):
                names = {f"{node.module}.{a.name}" for a in node.names}
                submodules = {n for n in names if _is_module(n)}
                # `from pkg import submodule` needs the submodule, not pkg's __init__
                found.update(submodules if submodules == names else {node.module} | submodules)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.startswith("evperc"))
        graph[name] = found
    modules = set(graph)
    return {m: {i for i in deps if i in modules and i != m} for m, deps in graph.items()}


def test_stages_import_only_upstream() -> None:
    wrong = []
    for module, deps in _imports().items():
        parts = module.split(".")
        if len(parts) < 3 or parts[1] not in ALLOWED:
            continue
        stage = parts[1]
        for dep in deps:
            top = dep.split(".")[1] if dep.count(".") else "__init__"
            if top not in SHARED and top != stage and top not in ALLOWED[stage]:
                wrong.append(f"{module} imports {dep}")
    assert not wrong, wrong


def test_no_import_cycle() -> None:
    graph = _imports()
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(node: str, trail: list[str]) -> None:
        state[node] = 1
        for dep in sorted(graph.get(node, ())):
            if state.get(dep) == 1:
                cycles.append(trail[trail.index(dep):] + [dep] if dep in trail else [node, dep])
            elif dep not in state:
                visit(dep, trail + [dep])
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not cycles, cycles


def test_the_checks_see_imports() -> None:
    """The graph is not empty where the layout says there are imports (a parser that found
    nothing would pass both tests above)."""
    graph = _imports()
    assert "evperc.output.layers" in graph["evperc.output.writer"]
    assert "evperc.logs.factory" in graph["evperc.runner"]
    assert "evperc.output.manifest" in graph["evperc.output.reader"]
