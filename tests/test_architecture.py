"""The package's shape: no import cycle between its modules (top-level imports), the board's view in
`board/` (link/ trains nothing), and no function-local import of the package's own modules where there is
no cycle to dodge, in the modules the zeroshot <-> board cycle ran through (board/, link.emulator, zeroshot)."""

from __future__ import annotations

import ast
from pathlib import Path

import impactsense

ROOT = Path(impactsense.__file__).resolve().parent
PACKAGE = "impactsense"


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES = {_module_name(p): p for p in ROOT.rglob("*.py")}


def _resolve(module: str, node: ast.ImportFrom, is_package: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    base = base if is_package else base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _targets(module: str, node) -> list[str]:
    """The package's modules an import statement loads."""
    path = MODULES[module]
    out = []
    if isinstance(node, ast.Import):
        out = [a.name for a in node.names]
    elif isinstance(node, ast.ImportFrom):
        base = _resolve(module, node, path.name == "__init__.py")
        for a in node.names:
            sub = f"{base}.{a.name}"
            out.append(sub if sub in MODULES else base)
    return [t for t in out if t in MODULES]


def _top_level_graph() -> dict[str, set[str]]:
    graph = {}
    for module, path in MODULES.items():
        tree = ast.parse(path.read_text())
        deps = set()
        for node in tree.body:
            for t in _targets(module, node) if isinstance(node, (ast.Import, ast.ImportFrom)) else []:
                # importing a.b.c runs a and a.b first (unless they are this module's own packages, which
                # are being imported already)
                parts = t.split(".")
                deps.update(p for p in (".".join(parts[:k]) for k in range(2, len(parts) + 1))
                            if not module.startswith(p + "."))
        graph[module] = deps - {module, PACKAGE}
    return graph


def _cycle(graph):
    state, stack = {}, []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                found = visit(m)
                if found:
                    return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            found = visit(n)
            if found:
                return found
    return None


def test_no_import_cycle():
    assert _cycle(_top_level_graph()) is None


def test_the_cycle_finder_finds_one():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_link_trains_nothing():
    """link/ is the wire, the monitor and the emulator: no model fitting (that is board.models)."""
    graph = _top_level_graph()
    trainers = {f"{PACKAGE}.models", f"{PACKAGE}.workflow", f"{PACKAGE}.zeroshot", f"{PACKAGE}.board.models"}
    for module, deps in graph.items():
        if module.startswith(f"{PACKAGE}.link"):
            assert not deps & trainers, (module, deps & trainers)


def _local_imports(path: Path, module: str) -> list[str]:
    tree = ast.parse(path.read_text())
    found = []
    for fn in ast.walk(tree):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)) and _targets(module, node):
                    found.append(f"{module}:{node.lineno}")
    return found


def test_no_local_imports_of_the_package_in_board_emulator_zeroshot():
    checked = [m for m in MODULES if m.startswith(f"{PACKAGE}.board")] + [f"{PACKAGE}.link.emulator",
                                                                          f"{PACKAGE}.zeroshot"]
    assert len(checked) >= 5
    local = [x for m in checked for x in _local_imports(MODULES[m], m)]
    assert local == []
