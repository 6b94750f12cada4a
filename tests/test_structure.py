"""The package stays readable in parts: no two modules import each other (directly or through others, at module
level or inside a function), no module is over 400 lines, and the roll-out's and the Predictor's public
functions take few enough parameters to call without a keyword list in hand.

The checks read the sources with ``ast``; each is also run on planted sources, so a broken detector cannot
pass for a clean package.
"""

from __future__ import annotations

import ast
from collections import deque
from pathlib import Path
from typing import Mapping

PACKAGE = Path(__file__).resolve().parents[1] / "physdyn"
MAX_LINES = 400
MAX_PARAMETERS = 8  # besides self / cls
ROLLOUT = PACKAGE / "eval" / "rollout.py"


# --------------------------------------------------------------------------------------------------
# Imports
# --------------------------------------------------------------------------------------------------
def package_sources(root: Path = PACKAGE) -> dict[str, tuple[str, bool]]:
    """Dotted module name -> (source, whether it is a package's ``__init__``) for every module under ``root``."""
    sources = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root.parent).with_suffix("").parts
        is_package = parts[-1] == "__init__"
        sources[".".join(parts[:-1] if is_package else parts)] = (path.read_text(encoding="utf-8"), is_package)
    return sources


def _known(name: str, modules: Mapping[str, object]) -> str | None:
    """The module ``name`` runs: itself, or the nearest enclosing one that exists (``a.b.Class`` -> ``a.b``)."""
    while name:
        if name in modules:
            return name
        name = name.rpartition(".")[0]
    return None


def import_graph(sources: Mapping[str, tuple[str, bool]]) -> dict[str, set[str]]:
    """Module -> the modules of ``sources`` it imports anywhere in its body (module level, in functions, under
    ``if``). ``from p import m`` where ``m`` is a module of ``p`` counts as importing ``p.m``."""
    graph: dict[str, set[str]] = {name: set() for name in sources}
    for name, (source, is_package) in sources.items():
        package = name if is_package else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(source)):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(anchor + ([node.module] if node.module else []))
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in sources else base
                           for alias in node.names]
            for target in targets:
                module = _known(target, sources)
                if module is not None and module != name:
                    graph[name].add(module)
    return graph


def _reachable(graph: Mapping[str, set[str]], start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for nxt in graph.get(todo.pop(), ()):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def import_cycles(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """One cycle ``[a, b, ..., a]`` for each group of modules that import each other (directly or through
    others); empty when the imports run one way."""
    reach = {name: _reachable(graph, name) for name in graph}
    cycles, placed = [], set()
    for name in sorted(graph):
        if name in placed or name not in reach[name]:
            continue
        group = {other for other in reach[name] if name in reach[other]}
        placed |= group
        # the shortest way from ``name`` back to itself inside its group
        came_from: dict[str, str] = {}
        todo = deque([name])
        while todo:
            here = todo.popleft()
            for nxt in sorted(graph[here] & group):
                if nxt == name:
                    path = [here]
                    while path[-1] != name:
                        path.append(came_from[path[-1]])
                    cycles.append(path[::-1] + [name])
                    todo.clear()
                    break
                if nxt not in came_from:
                    came_from[nxt] = here
                    todo.append(nxt)
    return cycles


def _cycle_text(cycles: list[list[str]], graph: Mapping[str, set[str]]) -> str:
    lines = []
    for cycle in cycles:
        group = sorted(m for m in graph if cycle[0] in _reachable(graph, m) and m in _reachable(graph, cycle[0]))
        extra = f" (the circle holds {len(group)} modules: {', '.join(group)})" if len(group) > len(cycle) - 1 else ""
        lines.append("  " + " -> ".join(cycle) + extra)
    return "\n".join(lines)


def test_no_module_imports_itself_through_others():
    graph = import_graph(package_sources())
    cycles = import_cycles(graph)
    assert not cycles, ("modules that import each other (module level or inside functions); move the shared part "
                        "into a module both import:\n" + _cycle_text(cycles, graph))


def test_the_cycle_finder_sees_lazy_submodule_and_relative_imports():
    planted = {
        "pkg": ("from pkg.a import f\n", True),
        "pkg.a": ("def f():\n    from pkg.b import g  # lazy\n    return g\n", False),
        "pkg.b": ("import pkg.c.d\ng = 1\n", False),
        "pkg.c": ("", True),
        "pkg.c.d": ("from pkg import a  # a submodule, not pkg's __init__\n", False),
        "pkg.e": ("from . import a\nfrom .c import d\n", False),  # one way only: no cycle
    }
    graph = import_graph(planted)
    assert graph["pkg.c.d"] == {"pkg.a"} and graph["pkg.e"] == {"pkg.a", "pkg.c.d"}
    assert import_cycles(graph) == [["pkg.a", "pkg.b", "pkg.c.d", "pkg.a"]]
    assert "pkg.a -> pkg.b -> pkg.c.d -> pkg.a" in _cycle_text(import_cycles(graph), graph)
    # a package that imports its own submodules, and submodules that import siblings, is not a cycle
    one_way = {"pkg": ("from pkg.a import x\nfrom pkg.b import y\n", True), "pkg.a": ("x = 1\n", False),
               "pkg.b": ("from pkg.a import x as y\n", False)}
    assert import_cycles(import_graph(one_way)) == []


# --------------------------------------------------------------------------------------------------
# Size
# --------------------------------------------------------------------------------------------------
def long_modules(root: Path = PACKAGE, limit: int = MAX_LINES) -> list[str]:
    found = []
    for path in sorted(root.rglob("*.py")):
        lines = len(path.read_text(encoding="utf-8").splitlines())
        if lines > limit:
            found.append(f"{path.relative_to(root.parent)}: {lines} lines")
    return found


def test_no_module_is_over_400_lines():
    long = long_modules()
    assert not long, f"modules over {MAX_LINES} lines; split them by job:\n  " + "\n  ".join(long)


def test_the_size_check_names_a_long_module(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "short.py").write_text("x = 1\n" * MAX_LINES)
    (tmp_path / "pkg" / "long.py").write_text("x = 1\n" * (MAX_LINES + 1))
    assert long_modules(tmp_path / "pkg") == [f"pkg/long.py: {MAX_LINES + 1} lines"]


# --------------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------------
def _parameters(function: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> int:
    args = function.args
    count = len(args.posonlyargs) + len(args.args) + len(args.kwonlyargs)
    count += (args.vararg is not None) + (args.kwarg is not None)
    static = any(isinstance(d, ast.Name) and d.id == "staticmethod" for d in function.decorator_list)
    return count - 1 if method and not static and (args.posonlyargs or args.args) else count


def crowded_functions(source: str, where: str, classes: tuple[str, ...] | None = None,
                      limit: int = MAX_PARAMETERS) -> list[str]:
    """``where:line name (n parameters)`` for each public function (module level) and public method taking
    more than ``limit`` parameters besides self / cls; with ``classes``, only those classes' methods."""
    found = []

    def check(function: ast.AST, name: str, method: bool) -> None:
        if isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)) and not function.name.startswith("_"):
            n = _parameters(function, method)
            if n > limit:
                found.append(f"{where}:{function.lineno} {name}{function.name} ({n} parameters)")

    for node in ast.parse(source).body:
        if classes is None:
            check(node, "", method=False)
        if isinstance(node, ast.ClassDef) and (classes is None or node.name in classes):
            for member in node.body:
                check(member, f"{node.name}.", method=True)
    return found


def test_the_rollout_and_the_predictors_public_functions_take_at_most_8_parameters():
    assert ROLLOUT.is_file(), f"{ROLLOUT} is gone: point this test at the roll-out engine"
    crowded = crowded_functions(ROLLOUT.read_text(encoding="utf-8"), str(ROLLOUT.relative_to(PACKAGE.parent)))
    holders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = path.read_text(encoding="utf-8")
        if "class Predictor" in source and any(isinstance(n, ast.ClassDef) and n.name == "Predictor"
                                               for n in ast.parse(source).body):
            holders.append(path)
            crowded += crowded_functions(source, str(path.relative_to(PACKAGE.parent)), classes=("Predictor",))
    assert holders, "no class Predictor in physdyn/"
    assert not crowded, (f"public functions with more than {MAX_PARAMETERS} parameters; group the options into a "
                         "request or settings object:\n  " + "\n  ".join(crowded))


def test_the_parameter_check_finds_a_planted_nine_parameter_function():
    planted = (
        "def push(a, b, c, d, e, f, g, h, i): ...\n"
        "def fine(a, b, c, d, e, f, g, *, h): ...\n"
        "def _private(a, b, c, d, e, f, g, h, i, j): ...\n"
        "class Predictor:\n"
        "    def predict(self, a, b, c, d, e, f, g, h): ...\n"
        "    def predict_many(self, a, b, c, d, e, f, g, *more, **options): ...\n"
        "    @staticmethod\n"
        "    def helper(a, b, c, d, e, f, g, h, i): ...\n"
        "    def _inner(self, a, b, c, d, e, f, g, h, i): ...\n"
        "class Other:\n"
        "    def wide(self, a, b, c, d, e, f, g, h, i): ...\n"
    )
    assert crowded_functions(planted, "m.py") == [
        "m.py:1 push (9 parameters)", "m.py:6 Predictor.predict_many (9 parameters)",
        "m.py:8 Predictor.helper (9 parameters)", "m.py:11 Other.wide (9 parameters)"]
    assert crowded_functions(planted, "m.py", classes=("Predictor",)) == [
        "m.py:6 Predictor.predict_many (9 parameters)", "m.py:8 Predictor.helper (9 parameters)"]
