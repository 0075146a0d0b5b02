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


# --- size: small modules and functions (issue 21) ------------------------------------------------------------

MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 500
SIM_SOURCES = ROOT.parents[1] / "sim"


def _long_functions(tree, limit):
    return [(node.name, node.lineno, node.end_lineno - node.lineno + 1) for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > limit]


def test_no_python_function_over_80_lines_and_no_module_over_500():
    long_functions, long_modules = [], []
    for module, path in MODULES.items():
        text = path.read_text()
        if text.count("\n") > MAX_MODULE_LINES:
            long_modules.append((module, text.count("\n")))
        long_functions += [(module, *f) for f in _long_functions(ast.parse(text), MAX_FUNCTION_LINES)]
    assert long_modules == [] and long_functions == []


def test_the_size_check_finds_a_long_function():
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    tree = ast.parse(f"def short():\n    return 1\n\n\ndef long():\n{body}\n    return 0\n")
    assert _long_functions(tree, MAX_FUNCTION_LINES) == [("long", 5, MAX_FUNCTION_LINES + 2)]


_CONTAINER = ("namespace", "struct", "class", "enum", "union", 'extern "C"')


def _cpp_long_functions(text: str, limit: int) -> list[tuple[int, int]]:
    """(first line, length) of the C++ function bodies in text longer than limit lines, by their braces: a
    brace opened at namespace / struct / class level, by a statement that is not one of those, starts a body."""
    import re

    stack, head, found = [], "", []
    for number, line in enumerate(text.splitlines(), 1):
        code = re.sub(r'"(\\.|[^"\\])*"', '""', re.sub(r"//.*", "", line))
        for ch in code:
            if ch == "{":
                if not stack or stack[-1][0] == "container":
                    statement = head.split(";")[-1].split("}")[-1].strip()
                    kind = "container" if re.search(r"\b(namespace|struct|class|enum|union)\b[^()]*$", statement) \
                        or statement.startswith('extern "C"') else "function"
                    stack.append((kind, number))
                else:
                    stack.append(("block", number))
                head = ""
            elif ch == "}":
                if stack:
                    kind, start = stack.pop()
                    if kind == "function" and number - start + 1 > limit:
                        found.append((start, number - start + 1))
                head = ""
            elif not stack or stack[-1][0] == "container":
                head += ch
        head += " "
    return found


def test_no_sim_cpp_function_over_80_lines():
    sources = sorted(p for ext in ("*.cpp", "*.h") for p in SIM_SOURCES.rglob(ext))
    if not sources:
        return          # an installed package without the source tree
    long = [(p.name, *f) for p in sources for f in _cpp_long_functions(p.read_text(), MAX_FUNCTION_LINES)]
    assert long == []


def test_the_cpp_size_check_sees_functions_inside_namespaces_and_structs():
    body = "\n".join(f"  x += {i};" for i in range(MAX_FUNCTION_LINES))
    text = ("namespace a {\nstruct S {\n  int f() { return 1; }\n};\n"
            f"int long_one(int x) {{\n{body}\n  return x;\n}}\n}}  // namespace a\n")
    assert _cpp_long_functions(text, MAX_FUNCTION_LINES) == [(5, MAX_FUNCTION_LINES + 3)]
