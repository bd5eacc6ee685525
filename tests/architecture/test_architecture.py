"""The layout's rules, checked on the source (DESIGN section 4, README "Code map").

The import graph of `bench`, `drivers` and `schedules` is read with `ast`, function-local
imports included (imports under `if TYPE_CHECKING:` are for the type checker only and
are left out). A failure names the offending module and edge.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("bench", "drivers", "schedules")
#: third-party packages only one place may import
ONLY_IN = {"textual": "bench.tui"}


@dataclass(frozen=True)
class Edge:
    source: str
    target: str
    line: int
    local: bool            # inside a function
    commented: bool        # a comment on its line or just above its group of imports
    path: str = ""

    def __str__(self) -> str:
        return f"{self.source} -> {self.target} ({self.path}:{self.line})"


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((REPO / pkg).rglob("*.py"))}


def _type_checking_nodes(tree: ast.Module) -> set[int]:
    ids: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            ids |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return ids


def _edges(name: str, path: Path, known: set[str]) -> list[Edge]:
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    tree = ast.parse(source)
    skip = _type_checking_nodes(tree)
    function_nodes = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                      for n in ast.walk(f)}
    edges = []
    for body_owner in ast.walk(tree):
        for field in ("body", "orelse", "finalbody", "handlers"):
            body = getattr(body_owner, field, None)
            if not isinstance(body, list):
                continue
            group_comment = False
            for k, stmt in enumerate(body):
                if not isinstance(stmt, (ast.Import, ast.ImportFrom)) or id(stmt) in skip:
                    group_comment = False
                    continue
                starts_group = k == 0 or not isinstance(body[k - 1], (ast.Import, ast.ImportFrom))
                if starts_group:
                    above = lines[stmt.lineno - 2].strip() if stmt.lineno >= 2 else ""
                    group_comment = above.startswith("#")
                commented = group_comment or "#" in lines[stmt.end_lineno - 1]
                if isinstance(stmt, ast.Import):
                    targets = [a.name for a in stmt.names]
                else:
                    base = stmt.module or ""
                    if stmt.level:
                        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                        package = package[:len(package) - stmt.level + 1]
                        base = ".".join(package + ([base] if base else []))
                    targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in stmt.names]
                for target in dict.fromkeys(targets):
                    edges.append(Edge(name, target, stmt.lineno, id(stmt) in function_nodes, commented,
                                      str(path.relative_to(REPO))))
    return edges


@pytest.fixture(scope="module")
def graph() -> dict[str, list[Edge]]:
    modules = _modules()
    known = set(modules)
    return {name: _edges(name, path, known) for name, path in modules.items()}


def _first_party(target: str) -> bool:
    return target.split(".")[0] in PACKAGES


def _inside(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def test_the_graph_sees_every_package(graph):
    assert {"bench.cli.main", "bench.run.runner", "drivers.turntable.base", "schedules.loader"} <= set(graph)
    assert any(e.target == "bench.run.sequencer" for e in graph["bench.run.runner"])


def test_nothing_below_the_cli_imports_it(graph):
    bad = [e for edges in graph.values() for e in edges
           if _inside(e.target, "bench.cli") and not _inside(e.source, "bench.cli")]
    assert not bad, "imports of bench.cli from outside it:\n" + "\n".join(map(str, bad))


def test_drivers_import_no_bench_and_schedules_import_neither(graph):
    bad = [e for edges in graph.values() for e in edges
           if (_inside(e.source, "drivers") and _inside(e.target, "bench"))
           or (_inside(e.source, "schedules") and (_inside(e.target, "bench") or _inside(e.target, "drivers")))]
    assert not bad, "forbidden edges:\n" + "\n".join(map(str, bad))


@pytest.mark.parametrize("library, owner", ONLY_IN.items())
def test_only_its_owner_imports_a_library(graph, library, owner):
    bad = [e for edges in graph.values() for e in edges
           if _inside(e.target, library) and not _inside(e.source, owner)]
    assert not bad, f"{library} imported outside {owner}:\n" + "\n".join(map(str, bad))


def _cycle(graph: dict[str, list[Edge]]) -> list[Edge] | None:
    """One import cycle between first-party modules (as its edges), or None."""
    adjacency = {m: [e for e in edges if e.target in graph and e.target != m] for m, edges in graph.items()}
    state: dict[str, int] = {}          # 1 = on the stack, 2 = done
    stack: list[Edge] = []

    def visit(module: str) -> list[Edge] | None:
        state[module] = 1
        for edge in adjacency[module]:
            if state.get(edge.target) == 1:
                start = next((k for k, e in enumerate(stack) if e.source == edge.target), len(stack))
                return stack[start:] + [edge]
            if edge.target not in state:
                stack.append(edge)
                found = visit(edge.target)
                if found:
                    return found
                stack.pop()
        state[module] = 2
        return None

    for module in sorted(graph):
        if module not in state:
            found = visit(module)
            if found:
                return found
    return None


def test_no_import_cycles(graph):
    cycle = _cycle(graph)
    assert cycle is None, "import cycle:\n" + "\n".join(map(str, cycle or []))


def test_the_cycle_finder_finds_a_cycle():
    a = Edge("a", "b", 1, False, False)
    b = Edge("b", "c", 1, True, True)
    c = Edge("c", "a", 1, False, False)
    assert _cycle({"a": [a], "b": [b], "c": [c]}) == [a, b, c]
    assert _cycle({"a": [a], "b": [], "c": [c]}) is None


def test_function_local_imports_say_why(graph):
    bad = [e for edges in graph.values() for e in edges if e.local and not e.commented]
    assert not bad, ("function-local imports without a comment saying why (an optional or heavy dependency, "
                     "or the CLI's start-up time):\n" + "\n".join(map(str, bad)))


def test_frame_names_agree_across_the_layers():
    # drivers and schedules cannot import bench, so each keeps the names; they must be the same
    from bench.model.kinematics import FRAMES
    from drivers.turntable import FRAMES as DRIVER_FRAMES
    from schedules.loader import FRAMES as SCHEDULE_FRAMES

    assert FRAMES == DRIVER_FRAMES == SCHEDULE_FRAMES == ("outer", "middle", "inner")
